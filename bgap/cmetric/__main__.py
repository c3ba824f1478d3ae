from bgap.runner.numerics import command

main = command("bgap.commands.cmetric")
if __name__ == "__main__":
    main()
