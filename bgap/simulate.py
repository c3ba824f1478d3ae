from bgap.runner.numerics import command

main = command("bgap.commands.simulate")
if __name__ == "__main__":
    main()
