from bgap.runner.numerics import command

main = command("bgap.commands.cmetric_search")
if __name__ == "__main__":
    main()
