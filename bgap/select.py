from bgap.runner.numerics import command

main = command("bgap.commands.select")
if __name__ == "__main__":
    main()
